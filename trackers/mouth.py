"""The mouth corners, found on the grey level around the upper-lip contour.

With the mouth open, the upper-lip contour follows a border of the cavity and its ends
fall short of the corners; :func:`mouth_corners` finds the lateral ends of the dark
mouth line or cavity instead. The :class:`~trackers.tracking.Tracker` uses it for the
``mouth_corner_*`` fiducials (``mouth_corner='profile'``).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["mouth_corners"]


def mouth_corners(gray, lip, *, origin=(0.0, 0.0), sigma: float = 1.0,
                  half_height: float | None = None, width: float | None = None,
                  previous=None, max_shift: float = 0.08):
    """Mouth corners as the lateral ends of the dark mouth line or cavity.

    A contour on the mouth line gives the commissures by its ends while the mouth is
    closed. When the jaw drops, the dark line becomes a cavity, the contour follows
    one of its borders (often the upper edge of the lower teeth) and its ends fall
    short of the corners, which lie higher, where the lips meet. Here the mouth is
    scanned along the chord of the contour (``lip``): at each step the darkest grey
    value (blurred by ``sigma``) across a window of ``+-half_height`` pixels around
    the chord line is taken, whichever part of the window the cavity or line is in.
    Going outward from the inner part of the mouth, the corner is where this profile
    first rises to half-way between the mouth's darkness and the skin beyond it.
    Its height is that of the darkest point of the window there.

    Parameters
    ----------
    gray : ndarray (H, W)
        Grey image (e.g. the tracker's crop).
    lip : array_like (n, 2)
        Mouth-line contour, image pixels, ordered either way.
    origin : (x, y)
        Image position of ``gray[0, 0]``.
    sigma : float
        Blur of the profile, pixels.
    half_height : float, optional
        Half-height of the window across the chord (default 15 % of ``width``).
    width : float, optional
        Expected mouth width, pixels (default: the chord's length). The scan
        reaches 30 % of it beyond the ends, plus half of what the contour is short
        of it (a contour on a cavity's border shrinks).
    previous : pair of (2,) arrays or None, optional
        The corners found on the previous frame (moved with the head), at the contour's
        first and last end. Where given, the window across the chord is narrowed to
        ``+-max_shift * width`` around that corner's height: corners move little from one
        frame to the next, while something dark beside the mouth (a furrow crossing the
        window when the upper lip lifts off the teeth) would otherwise win.
    max_shift : float
        Half-height of that narrowed window, as a fraction of the mouth width.

    Returns
    -------
    list of two ndarray (2,) or None
        The corners at the contour's first and last end (None where no clear end of
        the dark region is found).

    Examples
    --------
    >>> import numpy as np, cv2
    >>> img = np.full((60, 100), 200, np.uint8)
    >>> _ = cv2.line(img, (16, 30), (84, 30), 40, 2)  # where the lips meet (caps: 15..85)
    >>> _ = cv2.ellipse(img, (50, 30), (24, 6), 0, 0, 360, 30, -1)  # the open mouth
    >>> lip = np.c_[np.linspace(34, 66, 15), np.full(15, 34.0)]     # on its lower border
    >>> [np.round(c).tolist() for c in mouth_corners(img, lip, width=68)]
    [[15.0, 30.0], [85.0, 30.0]]
    """
    p = np.asarray(lip, float)
    if p.ndim != 2 or p.shape[1] != 2 or len(p) < 3:
        raise ValueError(f"lip must have shape (n >= 3, 2), got {p.shape}")
    g = np.asarray(gray, np.float32)
    if g.ndim != 2:
        raise ValueError(f"gray must be 2-D, got shape {g.shape}")
    chord = p[-1] - p[0]
    L = float(np.hypot(*chord))
    if L < 4:
        return [None, None]
    u = chord / L
    nrm = np.array([-u[1], u[0]])
    wid = L if width is None else max(float(width), L)
    h = 0.15 * wid if half_height is None else float(half_height)
    # the window is centred on the chord line through the middle of the contour's
    # height: an arched lip line or a cavity hangs below its chord
    mid = p.mean(axis=0)
    off = float((mid - p[0]) @ nrm)
    step = 0.5
    vs = np.arange(-h, h + 1e-9, 1.0) + 0.5 * off
    # blur only the part of the image the scan samples
    across = h + abs(off)
    for last, end in zip(previous if previous is not None else (), (p[0], p[-1])):
        if last is not None and np.isfinite(last).all():
            across = max(across, abs(float((np.asarray(last, float) - end) @ nrm))
                         + max(max_shift * wid, 2.0))
    pad = 0.3 * wid + 0.5 * (wid - L) + across + 4.0 * max(sigma, 0.5) + 2.0
    x0 = max(int(np.floor(p[:, 0].min() - pad - origin[0])), 0)
    y0 = max(int(np.floor(p[:, 1].min() - pad - origin[1])), 0)
    x1 = min(int(np.ceil(p[:, 0].max() + pad - origin[0])) + 1, g.shape[1])
    y1 = min(int(np.ceil(p[:, 1].max() + pad - origin[1])) + 1, g.shape[0])
    if x1 - x0 < 4 or y1 - y0 < 4:
        return [None, None]
    g = g[y0:y1, x0:x1]
    origin = (origin[0] + x0, origin[1] + y0)
    if sigma > 0:
        g = cv2.GaussianBlur(g, (0, 0), float(sigma))
    out = []
    prev = [None, None] if previous is None else list(previous)
    if len(prev) != 2:
        raise ValueError(f"previous must hold two corners (or None), got {len(prev)}")
    for end, direction, last in ((p[0], -u, prev[0]), (p[-1], u, prev[1])):
        ss = np.arange(-0.35 * L, 0.3 * wid + 0.5 * (wid - L) + 1e-9, step)
        vs_end = vs
        if last is not None and np.isfinite(last).all():
            centre = float((np.asarray(last, float) - end) @ nrm)
            reach = max(max_shift * wid, 2.0)
            vs_end = np.arange(centre - reach, centre + reach + 1e-9, 1.0)
        base = end + ss[:, None, None] * direction + vs_end[None, :, None] * nrm
        mx = (base[..., 0] - origin[0]).astype(np.float32)
        my = (base[..., 1] - origin[1]).astype(np.float32)
        vals = cv2.remap(g, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                         borderValue=np.nan)
        bad = np.isnan(vals).any(axis=1)
        if bad.any():
            # the scan left the image: keep what lies before
            first_bad = int(np.argmax(bad))
            if ss[first_bad] <= 0.05 * L:
                out.append(None)
                continue
            ss, vals = ss[:first_bad], vals[:first_bad]
        k = np.argmin(vals, axis=1)
        prof = vals[np.arange(len(ss)), k]
        inner = np.median(prof[ss <= -0.15 * L])
        beyond = prof[ss >= min(0.15 * L + 0.5 * (wid - L), ss[-1] - 2.0)]
        outer = np.median(beyond)
        if outer - inner < 8.0:
            out.append(None)
            continue
        half = 0.5 * (inner + outer)
        i0 = int(np.searchsorted(ss, -0.15 * L))
        found = None
        for i in range(max(i0, 1), len(ss)):
            if prof[i] > half >= prof[i - 1]:
                # an end: the profile stays up for 2 sigma (a highlight is no end)
                stay = prof[i:i + int(np.ceil(2 * max(sigma, 1.0) / step)) + 1]
                if (stay > half).all():
                    f = (half - prof[i - 1]) / (prof[i] - prof[i - 1])
                    found = i - 1 + f
                    break
        if found is None:
            out.append(None)
            continue
        i = int(found)
        t = found - i
        j = min(i + 1, len(ss) - 1)
        # height: where the window is darkest, just inside the end
        col = vals[max(i - 1, 0)]
        kk = int(k[max(i - 1, 0)])
        v = vs_end[kk]
        if 0 < kk < len(vs_end) - 1:
            den = col[kk - 1] - 2 * col[kk] + col[kk + 1]
            if den > 0:
                v += float(np.clip(0.5 * (col[kk - 1] - col[kk + 1]) / den, -0.5, 0.5)) \
                    * (vs_end[1] - vs_end[0])
        pt = end + ((1 - t) * ss[i] + t * ss[j]) * direction + v * nrm
        out.append(pt)
    return out
